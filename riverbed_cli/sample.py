"""A synthetic but realistic aerial block with exact geometry: the sample data of ``riverbed sample``.

The scene is a 2.5-D surface ``z = f(x, y)`` in a UTM world (EPSG:32632): sloping terrain, roads, houses with gable
and hip roofs, flat-roofed apartment blocks and an industrial hall (weakly textured roofs, tar roofs, solar panel
rows, roof units), trees with rounded crowns, a field with regular crop rows, a parking lot with stall lines and
cars, and a pond. A sun casts shadows (rays traced on the surface). Frame cameras fly one line with 60 % along-track
overlap; the rectified stereo pair of the first two exposures is rendered by casting the ray of every pixel onto the
surface, airborne LiDAR is simulated as an oscillating-mirror scanner on a few strips, and the ground truth (the
disparity of the pair and a DSM) is written beside them.

Geometry
--------
- World: EPSG:32632 easting, northing, ellipsoidal-like height (m). All computation happens in *local*
  coordinates, world minus :attr:`Scene.origin` (float64), which is also the pair file's ``origin``.
- The surface is a height field on a regular grid of nodes in a *grid frame* rotated about z by the flight
  heading (``u`` along the flight line, ``v`` to its left), interpolated **bilinearly** in each cell. Walls are
  one cell wide (a few cm) and steep. The surface is exactly this function: rays are intersected with it in closed
  form (a quadratic per cell, polished by a Newton step), found by a two-level grid traversal (blocks of cells
  with their maximum height, then cells), so a hit point lies on the surface to ~1e-9 m and on its pixel ray by
  construction: reprojection and triangulation close to rounding error.
- Cameras follow the pinhole model with pixel centres at integer coordinates: ``x ~ K R (X - C)``, ``R`` world to
  camera (x right, y down, z forward). The rectified pair shares ``R`` (x along the baseline, z as close to nadir
  as the baseline allows); the two principal points differ (a Middlebury-style ``doffs``) so that both images
  cover the along-track overlap and ground disparities are small and positive.
- Ground-truth disparity ``d = x_left - x_right`` of the hit point of each left pixel centre, NaN where that point
  is hidden from the right camera (a ray cast from the right camera meets the surface more than 1 mm before it)
  or falls outside the right image.
- Ground-truth DSM: the surface height at the centres of a north-up grid (``gsd`` cells, bounds snapped to whole
  metres) covering the left image's footprint; cells whose surface point is outside the left image are nodata
  (-9999).

Use
---
``riverbed sample OUTDIR [--size small|full] [--seed N]`` or ``python -m riverbed_cli.sample OUTDIR ...`` write a
block (:func:`generate_block`); :func:`make_block` returns it in memory (:class:`Block`: cameras, images, hit
points, ground truth, LiDAR arrays). :func:`render_view` renders any :class:`FrameCamera`, and
:func:`render_frame` the raw, slightly tilted frames of the flight line (the input a rectification step needs;
their orientations are in ``scene.json``). :func:`write_block` also writes the raw frames of the pair to
``raw/`` (grey ``frame0.png``, ``frame1.png``) with orientation files ``frame0.yaml``, ``frame1.yaml`` in the
format of ``riverbed rectify`` (:mod:`riverbed_cli.geometry.rectify`, ``docs/rectify.md``).

Everything is deterministic for a seed. The ray kernels are Numba functions (``cache=True``); the scene itself is
built with numpy and OpenCV resampling.
"""

import datetime
import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numba import njit, prange

from .errors import RiverbedError

CRS = "EPSG:32632"
#: Local origin (world coordinates of local 0, 0, 0) of every generated block: UTM 32N, northern Italy.
ORIGIN = (501230.0, 5002470.0, 200.0)
#: Flight direction, degrees clockwise from north (the rectified images' x axis points this way).
HEADING = 70.0
#: Sun position: azimuth (degrees clockwise from north) and elevation (degrees).
SUN_AZIMUTH, SUN_ELEVATION = 155.0, 38.0
#: DSM nodata value.
NODATA = -9999.0
#: Files of a block, in the order they are written.
#: Stages of :func:`make_block` and :func:`generate_block`, in order (for progress reporting).
STAGES = ("scene", "render", "ground_truth", "lidar", "write")
FILES = ("left.png", "right.png", "pair.yaml", "lidar.laz", "gt_disparity.tif", "gt_dsm.tif", "scene.json",
         "MANIFEST.md", "raw")
#: Raw (unrectified) frames of the pair written to ``raw/`` (``frameK.png`` and its orientation
#: ``frameK.yaml``).
RAW_FRAMES = (0, 1)
#: Pixel size (mm) stated in the raw frames' orientation files (focal length 12 mm small, 16 mm full).
RAW_PIXEL_SIZE_MM = 0.004

# Materials (node attribute; drive colour, LiDAR class and LiDAR drop-outs).
GRASS, ROAD, FIELD, ROOF, TREE, WATER, TAR, CAR, SOLAR, SOIL, PAVING = range(11)
MATERIAL_NAMES = ("grass", "road", "field", "roof", "tree", "water", "tar roof", "car", "solar panel", "soil",
                  "paving")
#: ASPRS class of a LiDAR return by material (2 ground, 5 high vegetation, 6 building, 9 water, 1 unclassified).
MATERIAL_CLASS = np.array([2, 2, 2, 6, 5, 9, 6, 1, 6, 2, 2], np.uint8)
#: Probability that a pulse on a material gives no return (dark or wet surfaces).
MATERIAL_DROPOUT = np.array([0.0, 0.02, 0.0, 0.0, 0.0, 0.96, 0.75, 0.1, 0.5, 0.0, 0.0])
_BUILDING_MATERIALS = (ROOF, TAR, SOLAR)

# Radiometry: irradiance of the sun (on a surface facing it) and of the sky (RGB, on a horizontal surface).
_E_SUN = 1.0
_E_SKY = np.array([0.085, 0.10, 0.135])
_GAMMA = 1.6  # tone curve of the camera: DN = 255 * (gain * radiance) ** (1 / gamma)
_GAIN = 2.7


@dataclass(frozen=True)
class SizeSpec:
    """Parameters of one block size.

    ``raw_size`` and ``rect_size`` are ``(width, height)`` in pixels with x along the flight line; ``cell`` is the
    spacing of the surface's nodes (m); LiDAR values are the scanner's height above ground (m), half field of view
    (deg), speed (m/s) and pulses per m^2 of one strip.
    """

    name: str
    gsd: float
    flying_height: float
    raw_size: tuple
    overlap: float
    rect_size: tuple
    cell: float
    exposures: int = 3
    supersample: int = 2
    lidar_agl: float = 500.0
    lidar_half_fov: float = 10.0
    lidar_speed: float = 60.0
    lidar_density: float = 0.5

    @property
    def focal(self):
        return self.flying_height / self.gsd

    @property
    def baseline(self):
        return (1.0 - self.overlap) * self.raw_size[0] * self.gsd


SIZES = {
    "small": SizeSpec("small", gsd=0.2, flying_height=600.0, raw_size=(1200, 800), overlap=0.6, rect_size=(720, 540),
                      cell=0.2 / 3),
    "full": SizeSpec("full", gsd=0.2, flying_height=800.0, raw_size=(3400, 2268), overlap=0.6,
                     rect_size=(2000, 1500), cell=0.1, lidar_half_fov=15.0),
}


# ---------------------------------------------------------------------------------------------------------------------
# Ray casting on a bilinear height field (Numba)
# ---------------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def _first_line(o, d, t, g0, size):
    """Index ``k`` of the first grid line ``g0 + k * size`` a ray ``o + t d`` (1-D, ``d != 0``) meets after ``t``."""
    k = float(math.floor((o + t * d - g0) / size))
    if d > 0.0:
        k += 1.0
    return k, (g0 + k * size - o) / d


@njit(cache=True)
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


@njit(cache=True, inline="always")
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


@njit(cache=True)
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


@njit(cache=True)
def _cast(ou, ov, oz, du, dv, dz, tmin, tmax, hgt, bmax, u0, v0, cell, bs, zlo, zhi):
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


@njit(cache=True)
def _locate(pu, pv, nu, nv, u0, v0, cell):
    """Cell ``(i, j)`` containing a grid-frame point and the point's fractional position ``(a, b)`` in it."""
    fu = (pu - u0) / cell
    fv = (pv - v0) / cell
    i = min(max(math.floor(fu), 0), nu - 2)
    j = min(max(math.floor(fv), 0), nv - 2)
    return i, j, fu - i, fv - j


@njit(cache=True)
def _bilinear(arr, i, j, a, b):
    return ((1.0 - a) * (1.0 - b) * float(arr[j, i]) + a * (1.0 - b) * float(arr[j, i + 1])
            + (1.0 - a) * b * float(arr[j + 1, i]) + a * b * float(arr[j + 1, i + 1]))


@njit(parallel=True, cache=True)
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
        i, j, a, b = _locate(pu, pv, nu, nv, u0, v0, cell)
        out[n] = _bilinear(hgt, i, j, a, b)


@njit(parallel=True, cache=True)
def _cast_kernel(orig, dirs, tmin, tmax, cr, sr, hgt, bmax, u0, v0, cell, bs, zlo, zhi, out):
    for n in prange(orig.shape[0]):
        ou = cr * orig[n, 0] + sr * orig[n, 1]
        ov = -sr * orig[n, 0] + cr * orig[n, 1]
        du = cr * dirs[n, 0] + sr * dirs[n, 1]
        dv = -sr * dirs[n, 0] + cr * dirs[n, 1]
        out[n] = _cast(ou, ov, orig[n, 2], du, dv, dirs[n, 2], tmin[n], tmax[n], hgt, bmax, u0, v0, cell, bs, zlo,
                       zhi)


@njit(cache=True)
def _shade(pu, pv, pz, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, out):
    """Radiance (RGB, linear) of the surface point ``(pu, pv, pz)`` (grid frame) lit by sun and sky.

    Lambertian: ``albedo * (E_sun * max(0, n . s) * lit + E_sky * (0.5 + 0.5 n_z))``; ``lit`` is 0 when a ray
    towards the sun meets the surface (cast shadow). Steep building cells (walls) get a facade pattern.
    Returns the material of the nearest node.
    """
    nv, nu = hgt.shape
    i, j, a, b = _locate(pu, pv, nu, nv, u0, v0, cell)
    h00 = float(hgt[j, i])
    h10 = float(hgt[j, i + 1])
    h01 = float(hgt[j + 1, i])
    h11 = float(hgt[j + 1, i + 1])
    e = h00 - h10 - h01 + h11
    gu = (h10 - h00 + e * b) / cell
    gv = (h01 - h00 + e * a) / cell
    norm = math.sqrt(gu * gu + gv * gv + 1.0)
    nx, ny, nz = -gu / norm, -gv / norm, 1.0 / norm
    m = mat[j + (1 if b >= 0.5 else 0), i + (1 if a >= 0.5 else 0)]
    r = _bilinear(alb[:, :, 0], i, j, a, b) / 65535.0
    g = _bilinear(alb[:, :, 1], i, j, a, b) / 65535.0
    bl = _bilinear(alb[:, :, 2], i, j, a, b) / 65535.0
    if nz < 0.35 and (m == ROOF or m == TAR or m == SOLAR):
        # A wall: render stucco with rows of windows (3 m storeys, 2.6 m bays).
        along = pu * ny - pv * nx
        fz = pz - 3.0 * math.floor(pz / 3.0)
        fa = along - 2.6 * math.floor(along / 2.6)
        if 1.0 < fz < 2.4 and 0.7 < fa < 1.9:
            r, g, bl = 0.05, 0.06, 0.08
        else:
            r, g, bl = 0.42, 0.38, 0.32
    ndots = nx * sun[0] + ny * sun[1] + nz * sun[2]
    direct = 0.0
    if ndots > 0.0:
        t = _cast(pu, pv, pz, sun[0], sun[1], sun[2], 2e-3, np.inf, hgt, bmax, u0, v0, cell, bs, zlo, zhi)
        if t < 0.0:
            direct = ndots
    skyw = 0.5 + 0.5 * nz
    out[0] = r * (_E_SUN * direct + sky[0] * skyw)
    out[1] = g * (_E_SUN * direct + sky[1] * skyw)
    out[2] = bl * (_E_SUN * direct + sky[2] * skyw)
    return m


@njit(parallel=True, cache=True)
def _render_kernel(Kinv, Rt, C, ss, cr, sr, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, rad, hits,
                   mats):
    height, width = mats.shape
    ogu = cr * C[0] + sr * C[1]
    ogv = -sr * C[0] + cr * C[1]
    for row in prange(height):
        px = np.empty(3)
        for col in range(width):
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            for k in range(ss * ss + 1):
                if k == ss * ss:  # the pixel centre: the geometry
                    x, y = float(col), float(row)
                else:
                    x = col - 0.5 + (k % ss + 0.5) / ss
                    y = row - 0.5 + (k // ss + 0.5) / ss
                c0 = Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2]
                c1 = Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2]
                c2 = Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2]
                dx = Rt[0, 0] * c0 + Rt[0, 1] * c1 + Rt[0, 2] * c2
                dy = Rt[1, 0] * c0 + Rt[1, 1] * c1 + Rt[1, 2] * c2
                dz = Rt[2, 0] * c0 + Rt[2, 1] * c1 + Rt[2, 2] * c2
                nrm = math.sqrt(dx * dx + dy * dy + dz * dz)
                dx /= nrm
                dy /= nrm
                dz /= nrm
                du = cr * dx + sr * dy
                dv = -sr * dx + cr * dy
                t = _cast(ogu, ogv, C[2], du, dv, dz, 0.0, np.inf, hgt, bmax, u0, v0, cell, bs, zlo, zhi)
                if k == ss * ss:
                    if t >= 0.0:
                        hits[row, col, 0] = C[0] + t * dx
                        hits[row, col, 1] = C[1] + t * dy
                        hits[row, col, 2] = C[2] + t * dz
                        i, j, a, b = _locate(ogu + t * du, ogv + t * dv, hgt.shape[1], hgt.shape[0], u0, v0, cell)
                        mats[row, col] = mat[j + (1 if b >= 0.5 else 0), i + (1 if a >= 0.5 else 0)]
                    else:
                        hits[row, col, 0] = np.nan
                        hits[row, col, 1] = np.nan
                        hits[row, col, 2] = np.nan
                        mats[row, col] = 255
                elif t >= 0.0:
                    _shade(ogu + t * du, ogv + t * dv, C[2] + t * dz, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo,
                           zhi, sun, sky, px)
                    acc0 += px[0]
                    acc1 += px[1]
                    acc2 += px[2]
                else:  # off the scene: sky-lit haze
                    acc0 += 0.3
                    acc1 += 0.3
                    acc2 += 0.3
            rad[row, col, 0] = acc0 / (ss * ss)
            rad[row, col, 1] = acc1 / (ss * ss)
            rad[row, col, 2] = acc2 / (ss * ss)


@njit(parallel=True, cache=True)
def _shade_points_kernel(pts, cr, sr, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, rad, mats):
    for n in prange(pts.shape[0]):
        px = np.empty(3)
        pu = cr * pts[n, 0] + sr * pts[n, 1]
        pv = -sr * pts[n, 0] + cr * pts[n, 1]
        mats[n] = _shade(pu, pv, pts[n, 2], hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, px)
        rad[n, 0] = px[0]
        rad[n, 1] = px[1]
        rad[n, 2] = px[2]


# ---------------------------------------------------------------------------------------------------------------------
# The scene
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class Scene:
    """A height field with albedo and materials, in a grid frame rotated by the flight heading.

    Node ``(j, i)`` lies at grid coordinates ``(u0 + i * cell, v0 + j * cell)``; grid coordinates relate to local
    ones (world minus ``origin``) by ``u = c x + s y``, ``v = -s x + c y`` with ``(c, s) = (cos, sin)`` of the
    angle from east to the flight direction. Heights are local (world height minus ``origin[2]``).
    """

    origin: np.ndarray
    heading: float
    u0: float
    v0: float
    cell: float
    height: np.ndarray  # (nv, nu) float32
    albedo: np.ndarray  # (nv, nu, 3) uint16, linear reflectance * 65535
    material: np.ndarray  # (nv, nu) uint8
    terrain: np.ndarray  # float32: the surface without trees at every tstep-th node (ground under the crowns)
    tstep: int
    block: int = 16
    block_max: np.ndarray = None
    zlo: float = 0.0
    zhi: float = 0.0
    sun_azimuth: float = SUN_AZIMUTH
    sun_elevation: float = SUN_ELEVATION
    layout: dict = field(default_factory=dict)

    def __post_init__(self):
        h = self.height
        nv, nu = h.shape
        bs = self.block
        nbv, nbu = -(-(nv - 1) // bs), -(-(nu - 1) // bs)
        pad = np.full((nbv * bs + 1, nbu * bs + 1), -np.inf, np.float32)
        pad[:nv, :nu] = h
        core = pad[:-1, :-1].reshape(nbv, bs, nbu, bs).max(axis=(1, 3))
        # Blocks share their edge nodes with the next block.
        edge_u = pad[:-1:, bs::bs].reshape(nbv, bs, nbu).max(axis=1)
        edge_v = pad[bs::bs, :-1].reshape(nbv, nbu, bs).max(axis=2)
        corner = pad[bs::bs, bs::bs]
        self.block_max = np.maximum(np.maximum(core, edge_u), np.maximum(edge_v, corner)).astype(np.float64)
        self.zlo = float(h.min()) - 0.01
        self.zhi = float(h.max()) + 0.01

    @property
    def rotation(self):
        a = math.radians(90.0 - self.heading)
        return math.cos(a), math.sin(a)

    @property
    def sun(self):
        """Unit vector towards the sun, local coordinates (east, north, up)."""
        az, el = math.radians(self.sun_azimuth), math.radians(self.sun_elevation)
        return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])

    def to_grid(self, xy):
        c, s = self.rotation
        xy = np.asarray(xy, np.float64)
        return np.stack([c * xy[..., 0] + s * xy[..., 1], -s * xy[..., 0] + c * xy[..., 1]], axis=-1)

    def to_local(self, uv):
        c, s = self.rotation
        uv = np.asarray(uv, np.float64)
        return np.stack([c * uv[..., 0] - s * uv[..., 1], s * uv[..., 0] + c * uv[..., 1]], axis=-1)

    def _args(self):
        c, s = self.rotation
        return (c, s, self.height, self.block_max, self.u0, self.v0, self.cell, self.block, self.zlo, self.zhi)

    def _sun_grid(self):
        c, s = self.rotation
        sx, sy, sz = self.sun
        return np.array([c * sx + s * sy, -s * sx + c * sy, sz])


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
    _cast_kernel(o, d, tmin, tmax, *scene._args(), out)
    return out


def shade_points(scene, points):
    """Linear RGB radiance and material of surface points (local coordinates), as an orthophoto would see them."""
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    rad = np.empty((len(pts), 3))
    mats = np.empty(len(pts), np.uint8)
    c, s = scene.rotation
    _shade_points_kernel(pts, c, s, scene.height, scene.block_max, scene.albedo, scene.material, scene.u0, scene.v0,
                         scene.cell, scene.block, scene.zlo, scene.zhi, scene._sun_grid(), _E_SKY, rad, mats)
    return rad, mats


def tone_map(radiance, gain=_GAIN):
    """Camera tone curve: linear radiance to 0..255 floats, ``255 * (gain * L) ** (1 / 1.6)``, clipped."""
    return 255.0 * np.clip(gain * np.asarray(radiance), 0.0, 1.0) ** (1.0 / _GAMMA)


# -- building the scene (numpy) ---------------------------------------------------------------------------------------
def _noise(rng, shape, scale):
    """Smooth zero-mean, unit-variance noise of feature size ``scale`` (in nodes) on a ``shape`` array (float32)."""
    scale = max(float(scale), 1.0)
    k = max(round(scale), 1)
    gh, gw = shape[0] // k + 4, shape[1] // k + 4
    g = rng.standard_normal((gh, gw)).astype(np.float32)
    if k == 1:
        return g[:shape[0], :shape[1]].copy()
    big = cv2.resize(g, (gw * k, gh * k), interpolation=cv2.INTER_CUBIC)[k:k + shape[0], k:k + shape[1]]
    return big / np.float32(0.78)  # bicubic interpolation of white noise keeps about 0.78 of its std


def _smoothstep(x, a, b):
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


class _Builder:
    """Paint terrain and objects into node arrays (grid frame)."""

    def __init__(self, spec, extent, rng):
        self.rng = rng
        self.cell = spec.cell
        ua, ub, va, vb = extent
        self.u0, self.v0 = ua, va
        self.nu = math.ceil((ub - ua) / self.cell) + 1
        self.nv = math.ceil((vb - va) / self.cell) + 1
        self.extent = (ua, ua + (self.nu - 1) * self.cell, va, va + (self.nv - 1) * self.cell)
        shape = (self.nv, self.nu)
        self.h = np.zeros(shape, np.float32)
        self.alb = np.zeros(shape + (3,), np.float32)
        self.mat = np.zeros(shape, np.uint8)
        self.objects = {"houses": 0, "flat_buildings": 0, "trees": 0, "cars": 0, "ponds": 0, "fields": 0}
        self.trees = []
        self.tstep = 8
        self.bare = None

    # geometry helpers
    def box(self, ua, ub, va, vb):
        """Node slices covering ``[ua, ub] x [va, vb]`` and the node coordinates there (or None if empty)."""
        i0 = max(math.floor((ua - self.u0) / self.cell), 0)
        i1 = min(math.ceil((ub - self.u0) / self.cell) + 1, self.nu)
        j0 = max(math.floor((va - self.v0) / self.cell), 0)
        j1 = min(math.ceil((vb - self.v0) / self.cell) + 1, self.nv)
        if i0 >= i1 or j0 >= j1:
            return None
        U = (self.u0 + np.arange(i0, i1) * self.cell)[None, :]
        V = (self.v0 + np.arange(j0, j1) * self.cell)[:, None]
        return (slice(j0, j1), slice(i0, i1)), U, V

    def n(self, shape, metres):
        return _noise(self.rng, shape, metres / self.cell)

    def paint(self, sl, mask, colour, material=None, texture=None):
        """Set albedo (``colour`` RGB times ``1 + texture``) and material where ``mask``."""
        a = self.alb[sl]
        col = np.asarray(colour, np.float32)
        val = col[None, None, :] * (1.0 if texture is None else (1.0 + texture)[..., None])
        a[mask] = np.broadcast_to(val, a.shape)[mask]
        if material is not None:
            self.mat[sl][mask] = material

    # the layers
    def terrain(self):
        rng = self.rng
        shape = (self.nv, self.nu)
        U = (self.u0 + np.arange(self.nu) * self.cell)[None, :].astype(np.float32)
        V = (self.v0 + np.arange(self.nv) * self.cell)[:, None].astype(np.float32)
        ang = rng.uniform(0, 2 * math.pi)
        slope = 0.025
        self.h[:] = 40.0 + slope * (math.cos(ang) * U + math.sin(ang) * V)
        self.h += 3.0 * self.n(shape, 70.0) + 0.8 * self.n(shape, 20.0) + 0.08 * self.n(shape, 4.0)
        # Grass: green, patchy, with dry spots; moderate texture at the pixel scale.
        tex = 0.22 * self.n(shape, 6.0) + 0.05 * self.n(shape, 1.2) + 0.03 * self.n(shape, 0.35)
        dry = _smoothstep(self.n(shape, 15.0), 0.6, 1.4)[..., None]
        green = np.array([0.075, 0.11, 0.045], np.float32)
        straw = np.array([0.15, 0.14, 0.085], np.float32)
        self.alb[:] = (green * (1 - dry) + straw * dry) * (1.0 + tex[..., None])
        self.mat[:] = GRASS
        self.slope = (slope, ang)

    def road_u(self, vc, ua, ub, width, dashed=True):
        """A road along u at ``v = vc``: flattened across, asphalt with weak texture, lane markings."""
        r = self.box(ua, ub, vc - width / 2 - 1.5, vc + width / 2 + 1.5)
        if r is None:
            return
        sl, U, V = r
        jc = round((vc - self.v0) / self.cell)
        centre = self.h[jc, sl[1]][None, :]
        d = np.abs(V - vc)
        w = 1.0 - _smoothstep(d, width / 2, width / 2 + 1.5)
        self.h[sl] = self.h[sl] * (1 - w) + centre * w
        self._asphalt(sl, np.broadcast_to(d <= width / 2, self.h[sl].shape), U, V, along=U, across=V - vc,
                      width=width, dashed=dashed)

    def road_v(self, uc, va, vb, width, dashed=True):
        r = self.box(uc - width / 2 - 1.5, uc + width / 2 + 1.5, va, vb)
        if r is None:
            return
        sl, U, V = r
        ic = round((uc - self.u0) / self.cell)
        centre = self.h[sl[0], ic][:, None]
        d = np.abs(U - uc)
        w = 1.0 - _smoothstep(d, width / 2, width / 2 + 1.5)
        w = w * (self.mat[sl] != ROAD)  # junctions: keep the first road's surface
        self.h[sl] = self.h[sl] * (1 - w) + centre * w
        mask = np.broadcast_to(d <= width / 2, self.h[sl].shape) & (self.mat[sl] != ROAD)
        self._asphalt(sl, mask, U, V, along=V, across=U - uc, width=width, dashed=dashed)

    def _asphalt(self, sl, mask, U, V, along, across, width, dashed):
        shape = self.h[sl].shape
        tex = 0.035 * self.n(shape, 0.3) + 0.05 * self.n(shape, 6.0)
        self.paint(sl, mask, (0.085, 0.085, 0.09), ROAD, tex)
        across = np.broadcast_to(across, shape)
        along = np.broadcast_to(along, shape)
        edge = np.abs(np.abs(across) - (width / 2 - 0.35)) < 0.08
        line = edge
        if dashed:
            line = line | ((np.abs(across) < 0.08) & (np.mod(along, 9.0) < 3.0))
        self.paint(sl, mask & line, (0.55, 0.55, 0.53), ROAD, 0.03 * self.n(shape, 0.3))

    def pond(self, uc, vc, ru, rv):
        r = self.box(uc - ru - 3, uc + ru + 3, vc - rv - 3, vc + rv + 3)
        if r is None:
            return
        sl, U, V = r
        q = np.sqrt(((U - uc) / ru) ** 2 + ((V - vc) / rv) ** 2)
        inside = q <= 1.0
        h = self.h[sl]
        level = float(h[inside].min()) - 0.4
        dist = (q - 1.0) * min(ru, rv)  # ~ metres outside the shore
        w = _smoothstep(dist, 0.0, 2.5)
        bank = (~inside) & (dist < 2.5)
        h[:] = np.where(inside, level, np.where(bank, level + 0.15 + (h - level - 0.15) * w, h))
        shape = h.shape
        self.paint(sl, bank, (0.10, 0.09, 0.06), SOIL, 0.15 * self.n(shape, 0.5))
        self.paint(sl, inside, (0.022, 0.036, 0.034), WATER, 0.02 * self.n(shape, 3.0))
        self.objects["ponds"] += 1

    def field(self, ua, ub, va, vb, period=1.6, rows_along_v=True):
        """Crop rows (low ridges, green on brown soil) repeating every ``period`` m."""
        r = self.box(ua, ub, va, vb)
        if r is None:
            return
        sl, U, V = r
        shape = self.h[sl].shape
        coord = np.broadcast_to(U if rows_along_v else V, shape)
        phase = np.cos(2 * math.pi * (coord - ua) / period)
        crop = _smoothstep(phase, -0.2, 0.5)
        crop = crop * (1.0 + 0.06 * self.n(shape, 3.0))
        soil = np.array([0.16, 0.12, 0.08], np.float32)
        green = np.array([0.06, 0.13, 0.04], np.float32)
        tex = 0.02 * self.n(shape, 0.4) + 0.04 * self.n(shape, 5.0)
        col = (soil * (1 - crop[..., None]) + green * crop[..., None]) * (1.0 + tex[..., None])
        self.alb[sl] = col
        self.mat[sl] = FIELD
        self.h[sl] += (0.12 * crop).astype(np.float32)
        self.objects["fields"] += 1

    def paving(self, ua, ub, va, vb, stalls=2.6):
        """A parking lot: asphalt with white stall lines every ``stalls`` m along u, two rows of stalls."""
        r = self.box(ua, ub, va, vb)
        if r is None:
            return
        sl, U, V = r
        shape = self.h[sl].shape
        h = self.h[sl]
        h[:] = float(np.median(h))
        self.paint(sl, np.ones(shape, bool), (0.10, 0.10, 0.10), PAVING,
                   0.03 * self.n(shape, 0.3) + 0.04 * self.n(shape, 4.0))
        vm = 0.5 * (va + vb)
        Ub, Vb = np.broadcast_to(U, shape), np.broadcast_to(V, shape)
        rowband = (np.abs(Vb - vm) > 3.0) & (np.abs(Vb - vm) < 8.0)
        line = rowband & (np.mod(Ub - ua, stalls) < 0.12)
        line |= np.abs(np.abs(Vb - vm) - 3.0) < 0.06
        self.paint(sl, line, (0.6, 0.6, 0.58), PAVING)
        stalls_u = np.arange(ua + stalls / 2, ub - stalls / 2, stalls)
        return [(u, vm + side * 5.5) for u in stalls_u for side in (-1, 1)]

    def building(self, uc, vc, length, width, angle, roof, eave, pitch=35.0, colour=None, material=ROOF,
                 details=True):
        """A building on a rotated rectangle: ``roof`` 'flat', 'gable' (ridge along ``length``) or 'hip'."""
        ca, sa = math.cos(angle), math.sin(angle)
        ext = 0.5 * (abs(length * ca) + abs(width * sa)) + 0.2, 0.5 * (abs(length * sa) + abs(width * ca)) + 0.2
        r = self.box(uc - ext[0], uc + ext[0], vc - ext[1], vc + ext[1])
        if r is None:
            return
        sl, U, V = r
        p = (U - uc) * ca + (V - vc) * sa
        q = -(U - uc) * sa + (V - vc) * ca
        a, b = length / 2, width / 2
        inside = (np.abs(p) <= a) & (np.abs(q) <= b)
        if not inside.any():
            return
        h = self.h[sl]
        base = float(h[inside].max()) + 0.15
        tanp = math.tan(math.radians(pitch))
        if roof == "gable":
            z = base + eave + tanp * (b - np.abs(q))
        elif roof == "hip":
            z = base + eave + tanp * np.minimum(b - np.abs(q), a - np.abs(p))
        else:
            z = np.broadcast_to(base + eave, inside.shape).astype(np.float64)
            if details:  # parapet
                rim = inside & ((a - np.abs(p) < 0.4) | (b - np.abs(q) < 0.4))
                z = np.where(rim, z + 0.6, z)
        h[inside] = np.broadcast_to(z, inside.shape)[inside]
        shape = h.shape
        rng = self.rng
        if colour is None:
            colour = (0.33, 0.32, 0.30)
        if roof == "flat":
            tex = 0.01 * self.n(shape, 0.5) + 0.02 * self.n(shape, 4.0)
        else:  # tiles: faint courses along the slope, each roof side lit differently by the sun
            tex = 0.03 * np.cos(2 * math.pi * np.abs(q) / 0.45) + 0.025 * self.n(shape, 1.5)
        self.paint(sl, inside, colour, material, tex)
        if roof != "flat" and details and rng.random() < 0.6:  # a chimney
            cp, cq = rng.uniform(-a + 1.5, a - 1.5), rng.uniform(0.3, b - 1.5) * rng.choice([-1, 1])
            chim = inside & (np.abs(p - cp) < 0.35) & (np.abs(q - cq) < 0.35)
            if chim.any():
                h[chim] = float(np.broadcast_to(z, shape)[chim].max()) + 1.0
                self.paint(sl, chim, (0.25, 0.12, 0.09), material)
        self.objects["houses" if roof != "flat" else "flat_buildings"] += 1
        return sl, p, q, inside, base + eave

    def roof_units(self, uc, vc, length, width, angle, top, n):
        """``n`` boxes (ventilation units) on a flat roof at height ``top``."""
        rng = self.rng
        for _ in range(n):
            lu, lv = rng.uniform(1.5, 3.5), rng.uniform(1.2, 2.5)
            pu = rng.uniform(-length / 2 + 3, length / 2 - 3)
            pv = rng.uniform(-width / 2 + 3, width / 2 - 3)
            ca, sa = math.cos(angle), math.sin(angle)
            self.box_object(uc + pu * ca - pv * sa, vc + pu * sa + pv * ca, lu, lv, angle, top + rng.uniform(1, 2),
                            (0.45, 0.45, 0.46), ROOF)

    def box_object(self, uc, vc, lu, lv, angle, ztop, colour, material, above_only=True):
        ca, sa = math.cos(angle), math.sin(angle)
        ext = 0.5 * (abs(lu * ca) + abs(lv * sa)) + 0.1, 0.5 * (abs(lu * sa) + abs(lv * ca)) + 0.1
        r = self.box(uc - ext[0], uc + ext[0], vc - ext[1], vc + ext[1])
        if r is None:
            return
        sl, U, V = r
        p = (U - uc) * ca + (V - vc) * sa
        q = -(U - uc) * sa + (V - vc) * ca
        inside = (np.abs(p) <= lu / 2) & (np.abs(q) <= lv / 2)
        h = self.h[sl]
        inside &= h < ztop
        h[inside] = ztop
        self.paint(sl, inside, colour, material, 0.02 * self.n(h.shape, 0.4))

    def car(self, uc, vc, angle):
        rng = self.rng
        r = self.box(uc - 3, uc + 3, vc - 3, vc + 3)
        if r is None:
            return
        sl, _, _ = r
        ground = float(np.median(self.h[sl]))
        palette = [(0.5, 0.5, 0.52), (0.05, 0.05, 0.06), (0.55, 0.08, 0.06), (0.1, 0.15, 0.35), (0.6, 0.6, 0.6),
                   (0.3, 0.3, 0.32)]
        col = palette[rng.integers(len(palette))]
        self.box_object(uc, vc, 4.4, 1.8, angle, ground + 0.85, col, CAR)
        self.box_object(uc + 0.2 * math.cos(angle), vc + 0.2 * math.sin(angle), 2.3, 1.55, angle, ground + 1.45,
                        (0.06, 0.07, 0.08), CAR)
        self.objects["cars"] += 1

    def tree(self, uc, vc, radius, top):
        """Plan a tree (planted by :meth:`plant_trees` once everything else stands)."""
        self.trees.append((uc, vc, radius, top, self.rng.uniform(0.3, 0.45), self.rng.uniform(0.8, 1.25, 3)))

    def plant_trees(self):
        """Keep a coarse copy of the tree-less surface (the ground under the crowns), then paint the trees."""
        self.bare = self.h[::self.tstep, ::self.tstep].copy()
        for args in self.trees:
            self._tree(*args)

    def _tree(self, uc, vc, radius, top, base_share, tint):
        """A tree: an ellipsoidal crown (base at 30-45 % of the top height) with leafy bumps, dark green."""
        r = self.box(uc - radius, uc + radius, vc - radius, vc + radius)
        if r is None:
            return
        sl, U, V = r
        h = self.h[sl]
        ground = float(np.min(h))
        rr = ((U - uc) ** 2 + (V - vc) ** 2) / radius**2
        inside = rr < 1.0
        shape = h.shape
        leaf = self.n(shape, 0.5)
        crown_base = top * base_share
        z = ground + crown_base + (top - crown_base) * np.sqrt(np.clip(1.0 - rr, 0.0, 1.0)) * (1.0 + 0.04 * leaf)
        z = z - 0.15 * np.clip(leaf, 0.0, None) * (1.0 - rr)  # gaps between leaf clusters
        upd = inside & (z > h)
        h[upd] = z[upd]
        tint = np.array([0.045, 0.085, 0.03], np.float32) * tint.astype(np.float32)
        self.paint(sl, upd, tint, TREE, 0.3 * leaf + 0.12 * self.n(shape, 0.25))
        self.objects["trees"] += 1

    def finish(self):
        alb = np.clip(self.alb, 0.0, 1.0)
        return (np.round(alb * 65535.0)).astype(np.uint16)


def _layout(b):
    """Plan and paint the town: roads, then blocks of houses, fields, parks, industry, apartments and forest.

    The four blocks around the main crossing (inside the rectified pair) are fixed in kind so that every
    difficulty appears in the pair: residential (north-west), pond and field (north-east), industrial hall with
    parking lot (south-west), apartment blocks with solar panels and a tar roof (south-east).
    """
    rng = b.rng
    ua, ub, va, vb = b.extent
    vm = -8.0 + rng.uniform(-1, 1)
    road_vs = [vm + k * 78.0 for k in range(-5, 6) if va + 12 < vm + k * 78.0 < vb - 12]
    um = 20.0 + rng.uniform(-2, 2)
    road_us = [um + k * 160.0 for k in range(-8, 9) if ua + 12 < um + k * 160.0 < ub - 12]
    for v in road_vs:
        b.road_u(v, ua, ub, 7.0 if v == vm else 6.0)
    for u in road_us:
        b.road_v(u, va, vb, 6.0)
    # Avenue trees along the main road.
    for side in (-1, 1):
        for u in np.arange(ua + 4, ub - 4, 11.0):
            if min(abs(u - x) for x in road_us) > 8:
                b.tree(u + rng.uniform(-1, 1), vm + side * (3.5 + 3.0), rng.uniform(2.8, 3.8), rng.uniform(9, 13))
    us = [ua] + road_us + [ub]
    vs = [va] + road_vs + [vb]
    kinds = []
    for ki in range(len(us) - 1):
        for kj in range(len(vs) - 1):
            a0 = us[ki] + (3.0 + 3.5 if ki > 0 else 0.0)
            a1 = us[ki + 1] - (3.0 + 3.5 if ki + 1 < len(us) - 1 else 0.0)
            c0 = vs[kj] + (3.5 + 4.0 if kj > 0 else 0.0)
            c1 = vs[kj + 1] - (3.5 + 4.0 if kj + 1 < len(vs) - 1 else 0.0)
            if a1 - a0 < 15 or c1 - c0 < 15:
                continue
            west = us[ki + 1] == um
            east = us[ki] == um
            north = vs[kj] == vm
            south = vs[kj + 1] == vm
            if west and north:
                kind = "residential"
            elif east and north:
                kind = "park_field"
            elif west and south:
                kind = "industrial"
            elif east and south:
                kind = "apartments"
            else:
                kind = ["residential", "field", "forest", "residential", "park_field", "apartments",
                        "industrial"][rng.integers(7)]
            kinds.append(kind)
            low_road, high_road = kj > 0, kj + 1 < len(vs) - 1
            # Face the main road when the block touches it, else a road, else the low edge.
            face = 1.0 if north else -1.0 if south else -1.0 if (high_road and not low_road) else 1.0
            # Put the block's main features next to the main crossing (inside the pair) when it touches it.
            toward = 1.0 if west else -1.0 if east else 0.0
            _FILLERS[kind](b, a0, a1, c0, c1, face, low_road and high_road, toward)
    b.plant_trees()
    return {"main_road_v": vm, "cross_road_u": um, "roads_u": road_vs, "roads_v": road_us, "blocks": kinds}


def _fill_residential(b, a0, a1, c0, c1, face, both_roads, toward):
    """Rows of lots facing the roads: a house each (gable, hip or flat), garden trees, sheds, a car."""
    rng = b.rng
    depth = 28.0
    rows = [(c0, 1.0) if face > 0 else (c1, -1.0)]
    if both_roads and c1 - c0 > 2 * depth:
        rows.append((c1, -1.0) if face > 0 else (c0, 1.0))
    for edge, sgn in rows:
        u = a0 + 1.0
        while u < a1 - 12.0:
            lot = rng.uniform(17.0, 22.0)
            if u + lot > a1:
                break
            L, W = rng.uniform(10.0, 14.0), rng.uniform(8.5, 11.0)
            along_road = rng.random() < 0.7
            angle = (0.0 if along_road else math.pi / 2) + math.radians(rng.uniform(-3, 3))
            uc = u + lot / 2 + rng.uniform(-1.0, 1.0)
            vc = edge + sgn * (6.0 + (W if along_road else L) / 2 + rng.uniform(0, 2))
            kind = rng.choice(["gable", "gable", "hip", "hip", "flat"])
            colour = [(0.30, 0.11, 0.07), (0.26, 0.14, 0.10), (0.13, 0.13, 0.14), (0.34, 0.20, 0.13)][
                rng.integers(4)]
            if kind == "flat":
                b.building(uc, vc, L, W, angle, "flat", rng.uniform(5.5, 7.0), colour=(0.36, 0.35, 0.33))
            else:
                b.building(uc, vc, L, W, angle, kind, rng.uniform(5.0, 6.5), rng.uniform(30, 42), colour)
            if rng.random() < 0.4:
                b.car(uc + sgn * 0.0 + (L / 2 + 3.0), edge + sgn * 4.0, math.pi / 2)
            for _ in range(rng.integers(0, 3)):
                b.tree(u + rng.uniform(3, lot - 3), edge + sgn * rng.uniform(depth - 8, depth - 3),
                       rng.uniform(2.0, 3.8), rng.uniform(6, 12))
            if rng.random() < 0.35:
                b.building(u + rng.uniform(3, lot - 3), edge + sgn * (depth - 4.5), 3.0, 2.5, 0.0, "flat", 2.4,
                           colour=(0.2, 0.18, 0.15), details=False)
            u += lot


def _fill_park_field(b, a0, a1, c0, c1, face, both_roads, toward):
    """A pond with trees near the road, a field with crop rows beyond."""
    rng = b.rng
    edge = c0 if face > 0 else c1
    park = min(30.0, 0.5 * (c1 - c0))
    ru, rv = rng.uniform(12, 16), rng.uniform(6.5, 8.5)
    uc = min(a0 + 12 + ru + rng.uniform(0, 10), a1 - ru - 4)
    vc = edge + face * (2 + rv)
    b.pond(uc, vc, ru, rv)
    for _ in range(rng.integers(8, 14)):
        ang = rng.uniform(0, 2 * math.pi)
        rad = rng.uniform(1.15, 1.8)
        tu, tv = uc + rad * ru * math.cos(ang), vc + rad * rv * math.sin(ang)
        if 2 < face * (tv - edge) < park - 2 and a0 + 3 < tu < a1 - 3:
            b.tree(tu, tv, rng.uniform(2.5, 4.5), rng.uniform(8, 16))
    if c1 - c0 - park > 12:
        lo, hi = (c0 + park, c1) if face > 0 else (c0, c1 - park)
        b.field(a0 + 2, a1 - 2, lo + 2, hi - 2, period=1.6, rows_along_v=True)


def _fill_field(b, a0, a1, c0, c1, face, both_roads, toward):
    b.field(a0 + 2, a1 - 2, c0 + 2, c1 - 2, period=b.rng.choice([1.6, 2.0, 0.9]),
            rows_along_v=bool(b.rng.random() < 0.6))


def _fill_forest(b, a0, a1, c0, c1, face, both_roads, toward):
    rng = b.rng
    for u in np.arange(a0 + 3, a1 - 3, 5.5):
        for v in np.arange(c0 + 3, c1 - 3, 5.5):
            if rng.random() < 0.85:
                b.tree(u + rng.uniform(-2, 2), v + rng.uniform(-2, 2), rng.uniform(2.5, 4.5), rng.uniform(14, 22))


def _fill_industrial(b, a0, a1, c0, c1, face, both_roads, toward):
    """A hall (flat, weakly textured roof, roof units, a tar patch) facing the road, a parking lot beside it."""
    rng = b.rng
    near, sgn = (c0, 1.0) if face > 0 else (c1, -1.0)  # the road the hall faces
    L = min(rng.uniform(44, 55), 0.55 * (a1 - a0))
    W = min(rng.uniform(24, 30), c1 - c0 - 6)
    uc = a1 - 4 - L / 2 if toward > 0 else a0 + 4 + L / 2
    vc = near + sgn * (5.0 + W / 2)
    out = b.building(uc, vc, L, W, 0.0, "flat", rng.uniform(9.0, 11.0), colour=(0.36, 0.36, 0.35))
    if out is not None:
        sl, p, q, inside, top = out
        tar = inside & (np.abs(p - L * 0.22) < L * 0.15) & (np.abs(q + W * 0.1) < W * 0.25)
        b.paint(sl, tar, (0.045, 0.045, 0.05), TAR, 0.02 * b.n(tar.shape, 0.5))
        # Skylight strips: a repetitive pattern across the roof.
        sky = inside & (np.abs(q) < W / 2 - 3) & (np.mod(p + L / 2, 4.0) < 1.0) & (p < -L * 0.1)
        b.paint(sl, sky, (0.55, 0.58, 0.6), ROOF, 0.01 * b.n(sky.shape, 0.5))
        b.roof_units(uc, vc, L, W, 0.0, top, 4)
    span = rng.uniform(34, 42)
    if toward > 0:
        pa0, pa1 = max(a0 + 2, uc - L / 2 - 4 - span), uc - L / 2 - 4
    else:
        pa0, pa1 = uc + L / 2 + 4, min(a1 - 2, uc + L / 2 + 4 + span)
    if pa1 - pa0 > 12:
        pv0 = near + sgn * 2.0
        pv1 = near + sgn * 20.0
        stalls = b.paving(pa0, pa1, min(pv0, pv1), max(pv0, pv1))
        for su, sv in stalls or []:
            if rng.random() < 0.55:
                b.car(su, sv, math.pi / 2 + math.radians(rng.uniform(-3, 3)))


def _fill_apartments(b, a0, a1, c0, c1, face, both_roads, toward):
    """Tall flat-roofed blocks: one with rows of solar panels, one with a dark tar roof; trees between."""
    rng = b.rng
    near, sgn = (c0, 1.0) if face > 0 else (c1, -1.0)
    u = a0 + 6
    k = 0
    while u + 30 < a1 - 4:
        L, W = rng.uniform(32, 42), rng.uniform(12, 15)
        L = min(L, a1 - 4 - u)
        vc = near + sgn * (8.0 + W / 2)
        if toward > 0:  # mirror: start next to the crossing at the block's east end
            u_left = a0 + a1 - u - L
        else:
            u_left = u
        hgt = rng.uniform(15, 20)
        tar = k % 2 == 1
        out = b.building(u_left + L / 2, vc, L, W, 0.0, "flat", hgt, colour=(0.045, 0.045, 0.05) if tar else
                         (0.34, 0.33, 0.31), material=TAR if tar else ROOF)
        if out is not None and not tar:
            sl, p, q, inside, top = out
            # Panel rows (constant-u lines every 2 m): tilted towards the sun, dark blue with bright frames.
            inrow = inside & (np.abs(q) < W / 2 - 1.2) & (np.abs(p) < L / 2 - 1.2)
            ph = np.mod(p + L / 2, 2.0)
            panel = inrow & (ph < 1.2)
            b.h[sl][panel] = (top + 0.15 + 0.35 * np.broadcast_to(ph, panel.shape)[panel]).astype(np.float32)
            b.paint(sl, panel, (0.03, 0.04, 0.08), SOLAR, 0.03 * b.n(panel.shape, 0.5))
            frame = panel & ((ph < 0.08) | (ph > 1.12))
            b.paint(sl, frame, (0.4, 0.4, 0.42), SOLAR)
        for _ in range(rng.integers(2, 5)):
            b.tree(u_left + rng.uniform(0, L), near + sgn * rng.uniform(2.0, 5.0), rng.uniform(2.0, 3.0),
                   rng.uniform(6, 9))
        u += L + rng.uniform(12, 18)
        k += 1


_FILLERS = {"residential": _fill_residential, "park_field": _fill_park_field, "field": _fill_field,
            "forest": _fill_forest, "industrial": _fill_industrial, "apartments": _fill_apartments}


def build_scene(spec, seed=0):
    """Build the scene of a block size (a :class:`SizeSpec` or its name) for a seed.

    The scene covers the nadir footprints of all exposures (at the mean terrain height) plus a 15 m margin, in
    the grid frame centred on the rectified pair.
    """
    spec = SIZES[spec] if isinstance(spec, str) else spec
    rng = np.random.default_rng([seed, 1])
    half_u = spec.raw_size[0] * spec.gsd / 2
    half_v = spec.raw_size[1] * spec.gsd / 2
    us = _exposure_us(spec)
    extent = (us[0] - half_u - 15.0, us[-1] + half_u + 15.0, -half_v - 15.0, half_v + 15.0)
    b = _Builder(spec, extent, rng)
    b.terrain()
    layout = _layout(b)
    layout["objects"] = dict(b.objects)
    layout["terrain_slope"] = {"gradient": b.slope[0], "towards_deg_from_u": math.degrees(b.slope[1])}
    # b.bare: the surface without trees every tstep-th node, for LiDAR returns from the ground under crowns.
    return Scene(origin=np.array(ORIGIN), heading=HEADING, u0=b.u0, v0=b.v0, cell=b.cell, height=b.h,
                 albedo=b.finish(), material=b.mat, terrain=b.bare, tstep=b.tstep, layout=layout)


def _exposure_us(spec):
    """Along-track (u) positions of the exposures: the rectified pair (exposures 0 and 1) straddles u = 0."""
    B = spec.baseline
    return [(k - 0.5) * B for k in range(spec.exposures)]


# ---------------------------------------------------------------------------------------------------------------------
# Cameras
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class FrameCamera:
    """A pinhole frame camera: ``[x, y, 1] ~ K R (X - C)`` with ``X`` in local coordinates (world minus origin).

    ``R`` maps local axes to camera axes (x right, y down, z forward, along the optical axis); pixel centres at
    integer coordinates; the image is ``width x height`` pixels.
    """

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    width: int
    height: int

    @property
    def P(self):
        """The 3 x 4 projection matrix (local coordinates to pixels)."""
        return self.K @ np.hstack([self.R, (-self.R @ self.C)[:, None]])

    def project(self, X):
        """Pixel coordinates ``(x, y)`` and depth along the optical axis of local points ``X`` (N, 3)."""
        cam = (np.asarray(X, np.float64) - self.C) @ self.R.T
        uvw = cam @ self.K.T
        return uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2], cam[:, 2]


def _rot(axis, deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    if axis == 0:
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == 1:
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def nadir_rotation(heading, attitude=(0.0, 0.0, 0.0)):
    """World-to-camera rotation of a nadir frame camera whose image x axis points along ``heading``.

    ``heading`` in degrees clockwise from north; ``attitude`` = (roll, pitch, yaw) in degrees: small rotations
    of the camera about its own x, y and z axes (applied in that order) away from the ideal nadir orientation.
    """
    a = math.radians(90.0 - heading)
    c, s = math.cos(a), math.sin(a)
    R0 = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    roll, pitch, yaw = attitude
    return _rot(2, yaw).T @ _rot(1, pitch).T @ _rot(0, roll).T @ R0


def exposures(scene, spec, seed=0):
    """The nadir frame cameras of the flight line (``spec.exposures`` of them, 60 % along-track overlap).

    Camera centres lie ``spec.flying_height`` above the median scene height; attitudes deviate from the ideal
    nadir by a few tenths of a degree (deterministic for the seed), as a real flight's would.
    """
    rng = np.random.default_rng([seed, 3])
    z = float(np.median(scene.height[::16, ::16])) + spec.flying_height
    z = round(z, 2)
    f = spec.focal
    W, H = spec.raw_size
    K = np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])
    cams = []
    for u in _exposure_us(spec):
        xy = scene.to_local(np.array([u, 0.0]))
        att = tuple(float(a) for a in np.round(rng.normal(0.0, 0.4, 3), 3))
        cams.append((FrameCamera(K.copy(), nadir_rotation(scene.heading, att), np.array([xy[0], xy[1], z]), W, H),
                     att))
    return cams


def rectified_pair(cam_left, cam_right, width, height, doffs):
    """The rectified cameras of two frame cameras: a shared rotation, x along the baseline, z nadir-most.

    Both keep the left camera's focal length; the principal points differ by ``doffs`` px (``cx_left -
    cx_right``), split symmetrically about the image centre, so ``d = f B / depth + doffs``.

    Returns
    -------
    left, right : FrameCamera
    P_left, P_right : (3, 4) float64
        Projection matrices (local coordinates); ``P_right`` is built from ``P_left`` so that rows 2 and 3 are
        identical and row 1 differs by a multiple of row 3 plus the baseline term (an exactly rectified pair).
    """
    Cl, Cr = cam_left.C, cam_right.C
    B = float(np.linalg.norm(Cr - Cl))
    x = (Cr - Cl) / B
    down = np.array([0.0, 0.0, -1.0])
    z = down - (down @ x) * x
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    f = float(cam_left.K[0, 0])
    cx_l = (width - 1) / 2 + doffs / 2
    cx_r = (width - 1) / 2 - doffs / 2
    cy = (height - 1) / 2
    Kl = np.array([[f, 0.0, cx_l], [0.0, f, cy], [0.0, 0.0, 1.0]])
    Kr = np.array([[f, 0.0, cx_r], [0.0, f, cy], [0.0, 0.0, 1.0]])
    left = FrameCamera(Kl, R, Cl.copy(), width, height)
    right = FrameCamera(Kr, R, Cl + B * x, width, height)
    P_left = left.P
    P_right = P_left.copy()
    P_right[0] = P_left[0] + (cx_r - cx_l) * P_left[2]
    P_right[0, 3] -= f * B
    return left, right, P_left, P_right


# ---------------------------------------------------------------------------------------------------------------------
# Rendering and ground truth
# ---------------------------------------------------------------------------------------------------------------------
def render_view(scene, camera, supersample=2):
    """Render any frame camera: radiance, and the surface point and material seen at every pixel centre.

    Each pixel's colour is the mean radiance of ``supersample**2`` rays spread over the pixel (box filter); its
    geometry is the ray through the pixel centre, intersected exactly with the surface.

    Returns
    -------
    radiance : (H, W, 3) float64
        Linear radiance (see :func:`tone_map` for the camera's DN).
    hits : (H, W, 3) float64
        Local coordinates of the surface point of each pixel centre (NaN where the ray leaves the scene).
    material : (H, W) uint8
        Material at the hit (255 where none).
    """
    H, W = camera.height, camera.width
    rad = np.empty((H, W, 3))
    hits = np.empty((H, W, 3))
    mats = np.empty((H, W), np.uint8)
    Kinv = np.linalg.inv(camera.K)
    c, s = scene.rotation
    _render_kernel(Kinv, np.ascontiguousarray(camera.R.T), np.ascontiguousarray(camera.C, np.float64),
                   int(supersample), c, s, scene.height, scene.block_max, scene.albedo, scene.material, scene.u0,
                   scene.v0, scene.cell, scene.block, scene.zlo, scene.zhi, scene._sun_grid(), _E_SKY, rad, hits,
                   mats)
    # Water reflects the sky through ripples: a shimmer that differs between viewpoints (matching fails there).
    water = mats == WATER
    if water.any():
        X = hits[water]
        ph = 0.37 * camera.C[0] + 0.61 * camera.C[1]
        rip = (np.sin(2.1 * X[:, 0] + 1.3 * X[:, 1] + ph) + np.sin(-0.9 * X[:, 0] + 2.7 * X[:, 1] + 1.7 * ph)
               + np.sin(3.3 * X[:, 0] - 1.9 * X[:, 1] + 2.3 * ph) + np.sin(0.4 * X[:, 0] + 0.55 * X[:, 1] + ph))
        rad[water] += (0.0035 * (2.0 + 0.5 * rip))[:, None] * np.array([0.8, 0.9, 1.0])
    return rad, hits, mats


def expose(radiance, rng, gain=_GAIN, blur=0.5):
    """Camera DN (uint8) of a radiance image: optics blur (Gaussian, ``blur`` px), tone curve, signal-dependent
    noise (1.4-2.7 DN)."""
    if blur:
        radiance = cv2.GaussianBlur(radiance, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
    dn = tone_map(radiance, gain)
    sigma = np.sqrt(2.0 + 0.02 * dn)
    dn = dn + sigma * rng.standard_normal(dn.shape)
    return np.clip(np.round(dn), 0, 255).astype(np.uint8)


def ground_truth_disparity(scene, hits, left, right, P_right, tolerance=1e-3):
    """Disparity ``d = x_left - x_right`` of each left pixel's surface point; NaN where the right camera does not see it.

    A point is hidden when the ray from the right camera towards it meets the surface more than ``tolerance`` m
    before it; points outside the right image are NaN too.

    Returns
    -------
    disp : (H, W) float64
    occluded : (H, W) bool
        Hidden from the right camera (inside the right image's field of view).
    """
    H, W = hits.shape[:2]
    X = hits.reshape(-1, 3)
    ok = np.isfinite(X[:, 0])
    Xh = np.hstack([X, np.ones((len(X), 1))])
    with np.errstate(invalid="ignore", divide="ignore"):
        uvw = Xh @ P_right.T
        xr = uvw[:, 0] / uvw[:, 2]
        yr = uvw[:, 1] / uvw[:, 2]
    inside = ok & (xr >= -0.5) & (xr < W - 0.5) & (yr >= -0.5) & (yr < H - 0.5)
    vec = X[inside] - right.C
    dist = np.linalg.norm(vec, axis=1)
    t = cast_rays(scene, np.broadcast_to(right.C, vec.shape), vec / dist[:, None], 0.0, dist + 1.0)
    visible = (t < 0) | (t >= dist - tolerance)
    cols = np.tile(np.arange(W, dtype=np.float64), H)
    disp = np.full(H * W, np.nan)
    idx = np.flatnonzero(inside)
    disp[idx[visible]] = cols[idx[visible]] - xr[idx[visible]]
    occluded = np.zeros(H * W, bool)
    occluded[idx[~visible]] = True
    return disp.reshape(H, W), occluded.reshape(H, W)


def ground_truth_dsm(scene, left, hits, resolution):
    """The surface height on a north-up grid covering the left image's footprint.

    Returns
    -------
    dsm : (rows, cols) float32
        World heights at cell centres; :data:`NODATA` where the cell centre's surface point is outside the left
        image (or the scene).
    grid : riverbed_cli.products.dsm.Grid
        Cells of ``resolution`` m (which should divide 1 m), bounds snapped outwards to whole metres (world
        coordinates).
    """
    from .products.dsm import Grid

    ox, oy, oz = scene.origin
    X = hits.reshape(-1, 3)
    X = X[np.isfinite(X[:, 0])]
    # Whole-metre bounds (exact in binary, on the lattice of any resolution dividing 1 m).
    xmin, xmax = math.floor(X[:, 0].min() + ox), math.ceil(X[:, 0].max() + ox)
    ymin, ymax = math.floor(X[:, 1].min() + oy), math.ceil(X[:, 1].max() + oy)
    grid = Grid(float(xmin), float(ymax), resolution, round((xmax - xmin) / resolution),
                round((ymax - ymin) / resolution))
    cols = grid.xmin + (np.arange(grid.width) + 0.5) * grid.resolution - ox
    rows = grid.ymax - (np.arange(grid.height) + 0.5) * grid.resolution - oy
    gx, gy = np.meshgrid(cols, rows)
    z = surface_height(scene, gx, gy)
    pts = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x, y, depth = left.project(pts)
    inside = (x >= -0.5) & (x < left.width - 0.5) & (y >= -0.5) & (y < left.height - 0.5) & (depth > 0)
    dsm = np.where(inside.reshape(z.shape) & np.isfinite(z), z + oz, NODATA).astype(np.float32)
    return dsm, grid


# ---------------------------------------------------------------------------------------------------------------------
# Airborne LiDAR
# ---------------------------------------------------------------------------------------------------------------------
def _bare_height(scene, u, v):
    """Bilinear height of the tree-less coarse surface at grid coordinates (for returns under crowns)."""
    step = scene.cell * scene.tstep
    T = scene.terrain
    fu = np.clip((u - scene.u0) / step, 0, T.shape[1] - 1.000001)
    fv = np.clip((v - scene.v0) / step, 0, T.shape[0] - 1.000001)
    i, j = np.floor(fu).astype(int), np.floor(fv).astype(int)
    a, b = fu - i, fv - j
    return ((1 - a) * (1 - b) * T[j, i] + a * (1 - b) * T[j, i + 1] + (1 - a) * b * T[j + 1, i]
            + a * b * T[j + 1, i + 1])


def simulate_scan(scene, spec, seed=0, range_noise=0.04):
    """Airborne LiDAR of the scene: an oscillating-mirror scanner flown along a few strips.

    Each strip flies parallel to the camera flight line at ``spec.lidar_agl`` m above the median ground, the
    mirror sweeping a zig-zag across the track (``+-spec.lidar_half_fov``); pulse and scan rates give
    ``spec.lidar_density`` pulses per m^2 per strip with equal spacing along and across the track at nadir.
    Strips overlap by a quarter of a swath and are flown in alternate directions; the platform rolls, pitches and
    drifts slightly. Every pulse is a ray cast onto the surface; the return gets Gaussian range noise
    (``range_noise`` m). Dark and wet materials often give no return (:data:`MATERIAL_DROPOUT`). Crowns give a
    second, last return from the ground beneath for 40 % of their pulses. A few outliers are added: birds above
    the scene and multipath returns below the ground, unclassified (class 1), and low-noise points classified 7.

    Returns
    -------
    dict of arrays
        ``xyz`` (N, 3) local coordinates, ``classification``, ``intensity``, ``rgb`` (uint16, the orthophoto
        colour), ``return_number``, ``number_of_returns``, ``gps_time``, ``scan_angle_deg``,
        ``scan_direction``, ``edge_of_flight_line``, ``point_source_id``, ``kind`` (0 surface, 1 ground under
        canopy, 2 unclassified outlier, 3 class-7 noise); and ``info`` (scanner parameters).
    """
    rng = np.random.default_rng([seed, 5])
    ua = scene.u0
    ub = scene.u0 + (scene.height.shape[1] - 1) * scene.cell
    vb = scene.v0 + (scene.height.shape[0] - 1) * scene.cell
    agl, speed = spec.lidar_agl, spec.lidar_speed
    half_fov = math.radians(spec.lidar_half_fov)
    half_swath = agl * math.tan(half_fov)
    spacing = 1.5 * half_swath
    m = max(1, math.ceil(vb / spacing - 0.5 + 1e-9))
    offsets = [(k + 0.5) * spacing for k in range(-m, m)]
    prf = spec.lidar_density * speed * 2 * half_swath
    f_scan = math.sqrt(speed * prf / (8 * half_swath))
    ground = float(np.median(scene.height[::16, ::16]))
    c, s = scene.rotation
    out = {k: [] for k in ("xyz", "mat", "ret", "nret", "time", "angle", "sdir", "edge", "src", "kind", "rng")}
    t_base = 405_000_000.0  # adjusted standard GPS time (GPS seconds - 1e9), June 2022
    for k, v_off in enumerate(offsets):
        forward = k % 2 == 0
        length = ub - ua + 60.0
        n = int(length / speed * prf)
        t = np.arange(n) / prf
        ph = rng.uniform(0, 2 * math.pi, 5)
        along = (ua - 30.0 + speed * t) if forward else (ub + 30.0 - speed * t)
        sgn = 1.0 if forward else -1.0
        x = f_scan * t + ph[0] / (2 * math.pi)
        tri = 4.0 * np.abs(x - np.floor(x + 0.5)) - 1.0  # zig-zag in [-1, 1]
        roll = math.radians(0.15) * np.sin(2 * math.pi * 0.21 * t + ph[1])
        pitch = math.radians(0.1) * np.sin(2 * math.pi * 0.13 * t + ph[2])
        theta = half_fov * tri + roll
        dv_ = np.sin(theta) * np.cos(pitch)
        du_ = sgn * np.sin(pitch)
        dz_ = -np.cos(theta) * np.cos(pitch)
        pv = v_off + 0.8 * np.sin(2 * math.pi * 0.02 * t + ph[3])
        pz = ground + agl + 0.5 * np.sin(2 * math.pi * 0.03 * t + ph[4])
        O = np.stack([c * along - s * pv, s * along + c * pv, pz], axis=1)
        D = np.stack([c * du_ - s * dv_, s * du_ + c * dv_, dz_], axis=1)
        D /= np.linalg.norm(D, axis=1)[:, None]
        th = cast_rays(scene, O, D)
        hit = th >= 0
        O, D, th, t, theta = O[hit], D[hit], th[hit], t[hit], theta[hit]
        sweep_up = np.diff(tri, append=tri[-1])[hit] > 0
        edge = (np.abs(tri) > 1.0 - 4.0 * f_scan / prf)[hit]
        P = O + th[:, None] * D
        mats = _materials_at(scene, P)
        keep = rng.random(len(P)) >= MATERIAL_DROPOUT[mats]
        O, D, th, t, theta, P, mats = O[keep], D[keep], th[keep], t[keep], theta[keep], P[keep], mats[keep]
        sweep_up, edge = sweep_up[keep], edge[keep]
        noisy = th + range_noise * rng.standard_normal(len(th))
        first = O + noisy[:, None] * D
        two = (mats == TREE) & (rng.random(len(P)) < 0.4)
        # Last returns from the ground under crowns: continue the ray down to the tree-less surface.
        Og, Dg, tg = O[two], D[two], th[two].copy()
        for _ in range(6):
            Q = Og + tg[:, None] * Dg
            gu, gv = c * Q[:, 0] + s * Q[:, 1], -s * Q[:, 0] + c * Q[:, 1]
            tg += (Q[:, 2] - _bare_height(scene, gu, gv)) / -Dg[:, 2]
        ok = tg > th[two] + 1.5
        idx = np.flatnonzero(two)[ok]
        tg = tg[ok] + range_noise * rng.standard_normal(ok.sum())
        last = O[idx] + tg[:, None] * D[idx]
        nret = np.ones(len(P), np.uint8)
        nret[idx] = 2
        # Interleave: each pulse's returns consecutively, in time order.
        order = np.argsort(np.concatenate([np.arange(len(P)) * 2, idx * 2 + 1]), kind="stable")

        def cat(a, b, order=order):
            return np.concatenate([a, b])[order]

        out["xyz"].append(cat(first, last))
        out["mat"].append(cat(mats, np.full(len(idx), GRASS, np.uint8)))
        out["ret"].append(cat(np.ones(len(P), np.uint8), np.full(len(idx), 2, np.uint8)))
        out["nret"].append(cat(nret, nret[idx]))
        out["time"].append(cat(t, t[idx]) + t_base + 600.0 * k)
        out["angle"].append(np.degrees(cat(theta, theta[idx])))
        out["sdir"].append(cat(sweep_up, sweep_up[idx]))
        out["edge"].append(cat(edge, edge[idx]))
        out["src"].append(np.full(len(P) + len(idx), k + 1, np.uint16))
        out["kind"].append(cat(np.zeros(len(P), np.uint8), np.ones(len(idx), np.uint8)))
        out["rng"].append(cat(noisy, tg))
    pts = {k: np.concatenate(v) for k, v in out.items()}
    n = len(pts["xyz"])
    cls = MATERIAL_CLASS[pts["mat"]].copy()
    cls[pts["kind"] == 1] = 2
    # Outliers: birds (small flocks 20-150 m above ground), multipath (3-15 m below), class-7 low noise.
    n_bird, n_mp, n_noise = max(4, n // 6000), max(4, n // 8000), max(6, n // 3000)
    pick = rng.choice(n, n_bird + n_mp + n_noise, replace=False)
    xyz = pts["xyz"].copy()
    kind = pts["kind"].copy()
    ia, ib, ic = pick[:n_bird], pick[n_bird:n_bird + n_mp], pick[n_bird + n_mp:]
    xyz[ia, 2] += rng.uniform(20, 150, len(ia))
    xyz[ib, 2] -= rng.uniform(3, 15, len(ib))
    xyz[ic, 2] += np.where(rng.random(len(ic)) < 0.8, -rng.uniform(5, 40, len(ic)), rng.uniform(40, 200, len(ic)))
    kind[ia], kind[ib], kind[ic] = 2, 2, 3
    cls[ia], cls[ib], cls[ic] = 1, 1, 7
    # Colour from the orthophoto (sun-lit, shadowed; no camera noise); intensity from the albedo and range.
    surf = pts["xyz"].copy()
    surf[:, 2] = np.nan_to_num(surface_height(scene, surf[:, 0], surf[:, 1]), nan=0.0)
    rad, _ = shade_points(scene, surf)
    rgb = (np.round(tone_map(rad)) * 257).astype(np.uint16)
    alb = _albedo_at(scene, pts["xyz"]).mean(axis=1)
    inten = 65535 * np.clip(2.2 * alb * (agl / pts["rng"]) ** 2, 0, 1) * np.where(pts["nret"] == 2, 0.55, 1.0)
    inten[kind >= 2] *= 0.2
    inten = np.clip(inten * (1 + 0.08 * rng.standard_normal(n)), 0, 65535).astype(np.uint16)
    return {
        "xyz": xyz, "classification": cls, "intensity": inten, "rgb": rgb, "return_number": pts["ret"],
        "number_of_returns": pts["nret"], "gps_time": pts["time"], "scan_angle_deg": pts["angle"],
        "scan_direction": pts["sdir"], "edge_of_flight_line": pts["edge"], "point_source_id": pts["src"],
        "kind": kind,
        "info": {"strips": len(offsets), "strip_offsets_m": [round(o, 3) for o in offsets], "agl_m": agl,
                 "speed_mps": speed, "half_fov_deg": spec.lidar_half_fov, "pulse_rate_hz": round(prf, 1),
                 "scan_rate_hz": round(f_scan, 3), "density_per_strip_m2": spec.lidar_density,
                 "range_noise_m": range_noise, "under_canopy_share": 0.4,
                 "dropout": {MATERIAL_NAMES[i]: float(p) for i, p in enumerate(MATERIAL_DROPOUT) if p > 0},
                 "outliers": {"birds_class1": int(n_bird), "multipath_class1": int(n_mp),
                              "noise_class7": int(n_noise)}},
    }


def _node_index(scene, P):
    c, s = scene.rotation
    u = c * P[:, 0] + s * P[:, 1]
    v = -s * P[:, 0] + c * P[:, 1]
    nv, nu = scene.height.shape
    i = np.clip(np.round((u - scene.u0) / scene.cell).astype(np.int64), 0, nu - 1)
    j = np.clip(np.round((v - scene.v0) / scene.cell).astype(np.int64), 0, nv - 1)
    return j, i


def _materials_at(scene, P):
    j, i = _node_index(scene, P)
    return scene.material[j, i]


def _albedo_at(scene, P):
    j, i = _node_index(scene, P)
    return scene.albedo[j, i].astype(np.float64) / 65535.0


# ---------------------------------------------------------------------------------------------------------------------
# The block
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class Block:
    """Everything of a generated block, in memory (what :func:`write_block` puts on disk, and more).

    ``hits_left`` (H, W, 3) are the local coordinates of each left pixel centre's surface point; ``gt_disparity``
    is float64 (the file holds float32); ``occluded`` marks left pixels hidden from the right camera.
    """

    spec: SizeSpec
    seed: int
    scene: Scene
    frames: list  # [(FrameCamera, attitude)] of the flight line
    left_cam: FrameCamera
    right_cam: FrameCamera
    P_left: np.ndarray
    P_right: np.ndarray
    doffs: float
    left: np.ndarray
    right: np.ndarray
    hits_left: np.ndarray
    material_left: np.ndarray
    gt_disparity: np.ndarray
    occluded: np.ndarray
    lidar: dict
    dsm: np.ndarray
    dsm_grid: object
    seconds: dict = field(default_factory=dict)

    def pair(self, folder=None):
        """The pair as a :class:`~riverbed_cli.geometry.cameras.PairGeometry` (images in ``folder`` if given)."""
        from .geometry.cameras import PairGeometry

        folder = Path(folder) if folder is not None else None
        return PairGeometry(P_left=self.P_left, P_right=self.P_right, origin=self.scene.origin, crs=CRS,
                            left=folder / "left.png" if folder else None,
                            right=folder / "right.png" if folder else None,
                            width=self.left_cam.width, height=self.left_cam.height)


def make_block(size="small", seed=0, progress=None):
    """Generate a block in memory: scene, cameras, rectified pair, LiDAR and ground truth (deterministic).

    ``progress``, if given, is called with the name of each stage of :data:`STAGES` as it finishes (but the last).
    """
    if size not in SIZES:
        raise RiverbedError(f"unknown size '{size}' (use one of {', '.join(SIZES)})")
    spec = SIZES[size]
    seconds = {}
    done = progress or (lambda stage: None)
    t0 = time.perf_counter()
    scene = build_scene(spec, seed)
    seconds["scene"] = time.perf_counter() - t0
    done("scene")
    frames = exposures(scene, spec, seed)
    W, H = spec.rect_size
    # doffs: the lowest ground in the pair's footprint gets a disparity of about 4 px.
    lo = _footprint_min(scene, W * spec.gsd / 2 + 10, H * spec.gsd / 2 + 10)
    zmax_depth = frames[0][0].C[2] - lo
    doffs = round(4.0 - spec.focal * spec.baseline / zmax_depth, 2)
    left_cam, right_cam, P_left, P_right = rectified_pair(frames[0][0], frames[1][0], W, H, doffs)
    t0 = time.perf_counter()
    rad_l, hits, mats = render_view(scene, left_cam, spec.supersample)
    rad_r, _, _ = render_view(scene, right_cam, spec.supersample)
    left = expose(rad_l, np.random.default_rng([seed, 7]))
    right = expose(rad_r, np.random.default_rng([seed, 8]), gain=_GAIN * 0.97)  # a slightly different exposure
    seconds["render"] = time.perf_counter() - t0
    done("render")
    t0 = time.perf_counter()
    disp, occluded = ground_truth_disparity(scene, hits, left_cam, right_cam, P_right)
    dsm, grid = ground_truth_dsm(scene, left_cam, hits, spec.gsd)
    seconds["ground_truth"] = time.perf_counter() - t0
    done("ground_truth")
    t0 = time.perf_counter()
    lidar = simulate_scan(scene, spec, seed)
    seconds["lidar"] = time.perf_counter() - t0
    done("lidar")
    return Block(spec, seed, scene, frames, left_cam, right_cam, P_left, P_right, doffs, left, right, hits, mats,
                 disp, occluded, lidar, dsm, grid, seconds)


def render_frame(block, k, window=None):
    """Render raw (unrectified) frame ``k`` of the block's flight line, as its camera recorded it.

    Parameters
    ----------
    block : Block
    k : int
        Exposure index (``block.frames[k]``: camera and roll/pitch/yaw, also listed in ``scene.json``).
    window : (col0, row0, width, height), optional
        Render only this window of the frame (the camera's principal point shifted accordingly).

    Returns
    -------
    image : (H, W, 3) uint8
        With the same tone curve, optics blur and noise model as the rectified pair (noise seeded by seed and k).
    camera : FrameCamera
        The camera of the rendered window.
    hits : (H, W, 3) float64
        Local coordinates of each pixel centre's surface point.
    """
    cam = block.frames[k][0]
    if window is not None:
        c0, r0, w, h = window
        K = cam.K.copy()
        K[0, 2] -= c0
        K[1, 2] -= r0
        cam = FrameCamera(K, cam.R, cam.C, int(w), int(h))
    rad, hits, _ = render_view(block.scene, cam, block.spec.supersample)
    return expose(rad, np.random.default_rng([block.seed, 20 + k])), cam, hits


def _footprint_min(scene, half_u, half_v):
    """Lowest surface height in the grid-frame box ``|u| <= half_u``, ``|v| <= half_v``."""
    i0 = max(int((-half_u - scene.u0) / scene.cell), 0)
    i1 = int((half_u - scene.u0) / scene.cell) + 1
    j0 = max(int((-half_v - scene.v0) / scene.cell), 0)
    j1 = int((half_v - scene.v0) / scene.cell) + 1
    return float(scene.height[j0:j1, i0:i1].min())


def _world_matrix(a):
    return [[float(v) for v in row] for row in np.asarray(a)]


def scene_description(block):
    """The contents of ``scene.json``: seed, sun, cameras, LiDAR scanner, DSM grid and scene layout."""
    spec, scene = block.spec, block.scene
    origin = scene.origin
    frames = []
    for k, (cam, att) in enumerate(block.frames):
        frames.append({"id": k, "centre": [float(v) for v in cam.C + origin], "R": _world_matrix(cam.R),
                       "roll_pitch_yaw_deg": list(att), "K": _world_matrix(cam.K), "width": cam.width,
                       "height": cam.height})
    d = block.gt_disparity[np.isfinite(block.gt_disparity)]
    lid = block.lidar
    classes, counts = np.unique(lid["classification"], return_counts=True)
    g = block.dsm_grid
    return {
        "generator": "riverbed sample (riverbed_cli/sample.py)",
        "size": spec.name,
        "seed": block.seed,
        "crs": CRS,
        "origin": [float(v) for v in origin],
        "conventions": "local = world - origin (m); R maps local axes to camera axes (x right, y down, z forward); "
                       "[x, y, 1] ~ K R (X - C); pixel centres at integer coordinates; d = x_left - x_right",
        "sun": {"azimuth_deg": scene.sun_azimuth, "elevation_deg": scene.sun_elevation,
                "direction": [float(v) for v in scene.sun]},
        "flight": {"heading_deg": scene.heading, "flying_height_m": spec.flying_height, "gsd_m": spec.gsd,
                   "focal_px": spec.focal, "overlap": spec.overlap, "baseline_m": spec.baseline},
        "frames": frames,
        "pair": {"frames": [0, 1], "width": block.left_cam.width, "height": block.left_cam.height,
                 "R": _world_matrix(block.left_cam.R), "K_left": _world_matrix(block.left_cam.K),
                 "K_right": _world_matrix(block.right_cam.K), "doffs_px": block.doffs,
                 "baseline_m": float(np.linalg.norm(block.right_cam.C - block.left_cam.C)),
                 "disparity_range_px": [round(float(d.min()), 3), round(float(d.max()), 3)],
                 "gt_valid_share": round(float(np.isfinite(block.gt_disparity).mean()), 5),
                 "occluded_share": round(float(block.occluded.mean()), 5)},
        "lidar": {**lid["info"], "points": len(lid["xyz"]),
                  "classes": {str(int(c)): int(n) for c, n in zip(classes, counts)}},
        "dsm": {"resolution_m": g.resolution, "bounds": [float(v) for v in g.bounds], "width": g.width,
                "height": g.height, "nodata": NODATA,
                "definition": "surface height at cell centres; nodata outside the left image's footprint"},
        "scene": {"cell_m": scene.cell, "nodes": list(scene.height.shape[::-1]),
                  "extent_uv_m": [scene.u0, scene.u0 + (scene.height.shape[1] - 1) * scene.cell, scene.v0,
                                  scene.v0 + (scene.height.shape[0] - 1) * scene.cell],
                  "height_range_m": [round(scene.zlo + origin[2], 3), round(scene.zhi + origin[2], 3)],
                  **scene.layout},
    }


def _manifest(block, command):
    spec = block.spec
    W, H = spec.rect_size
    RW, RH = spec.raw_size
    lid = block.lidar
    info = lid["info"]
    g = block.dsm_grid
    d = block.gt_disparity[np.isfinite(block.gt_disparity)]
    ox, oy, oz = (float(v) for v in block.scene.origin)
    B = float(np.linalg.norm(block.right_cam.C - block.left_cam.C))
    return f"""# Synthetic aerial block (size {spec.name}, seed {block.seed})

Generated by

    {command}

(`riverbed_cli/sample.py`; `python -m riverbed_cli.sample OUTDIR` does the same). Deterministic: the same command
regenerates these files, which `tests/test_sample.py` checks. Synthetic data made by this project.

| file | what |
|---|---|
| `left.png`, `right.png` | rectified stereo pair, {W}x{H} RGB 8-bit, rendered by ray casting |
| `pair.yaml` | pair file: `P_left`, `P_right` (world minus `origin` -> pixels), `origin`, `crs` |
| `lidar.laz` | airborne LiDAR, {len(lid["xyz"])} points, LAS 1.4 point format 7 (RGB, GPS time), WKT CRS, 1 mm |
| `gt_disparity.tif` | ground-truth disparity of the left image, float32, `d = x_left - x_right`, NaN unknown |
| `gt_dsm.tif` | ground-truth DSM, float32 cloud-optimised GeoTIFF, nodata {NODATA:g} off the left footprint |
| `scene.json` | sun, flight line with the raw frame cameras, rectified cameras, LiDAR scanner, DSM grid, layout |
| `raw/frame0.png`, `raw/frame1.png` | raw (unrectified, slightly tilted) frames of the pair, {RW}x{RH} grey |
| `raw/frame0.yaml`, `raw/frame1.yaml` | their orientations (docs/rectify.md): input of `riverbed rectify` |

## Geometry

- CRS {CRS} (UTM 32N). World = local + origin, origin ({ox:.1f}, {oy:.1f}, {oz:.1f}).
- Pair: frames 0 and 1 of a {spec.exposures}-frame nadir flight line (heading {HEADING:g} deg, {100 * spec.overlap:.0f} %
  overlap), {spec.flying_height:g} m above ground, f = {spec.focal:g} px, GSD {spec.gsd:g} m, baseline {B:.2f} m,
  doffs {block.doffs:g} px (`d = f B / depth + doffs`); GT disparity {d.min():.2f} to {d.max():.2f} px, NaN on
  {100 * (1 - np.isfinite(block.gt_disparity).mean()):.1f} % of the pixels (hidden from the right camera or
  outside the right image).
- GT DSM: {g.resolution:g} m north-up cells, {g.width}x{g.height}, bounds
  ({g.bounds[0]:.1f}, {g.bounds[1]:.1f}, {g.bounds[2]:.1f}, {g.bounds[3]:.1f}); the surface height at cell centres.
- Exact: every pixel's surface point lies on its pixel ray (reprojection and triangulation close to ~1e-12).

## Scene and sensors

Sloping terrain, roads, houses with gable and hip roofs, flat-roofed blocks and an industrial hall (weakly textured
roofs, tar roof patches, skylights, solar panel rows every 2 m), trees, a field with crop rows every 1.6 m, a
parking lot with stall lines and cars, and a pond. Sun at azimuth {SUN_AZIMUTH:g} deg, elevation {SUN_ELEVATION:g}
deg: long, dark cast shadows. Images: 2x2 rays per pixel, 0.5 px optics blur, 1.4-2.7 DN noise; the right image
is exposed 3 % darker. LiDAR: oscillating-mirror zig-zag scan, {info["strips"]} strips at {info["agl_m"]:g} m,
{info["pulse_rate_hz"]:g} Hz pulses, {info["scan_rate_hz"]:g} Hz scan, {info["range_noise_m"]:g} m range noise;
classes 2 ground, 5 high vegetation, 6 building, 9 water, 1 unclassified (cars; outliers: birds, multipath below
ground), 7 low noise; few or no returns on water, tar roofs and solar panels; 40 % of the pulses hitting crowns
also return from the ground beneath (hidden from the cameras).
"""


def write_block(block, outdir, overwrite=False, command=None):
    """Write a block's files into ``outdir`` (created if missing), all or nothing.

    The files are written into a temporary folder beside ``outdir`` and moved in only once all exist; an existing
    file of the block in ``outdir`` is replaced only with ``overwrite``.

    Returns
    -------
    dict
        File name -> size in bytes.
    """
    from .io.atomic import check_output_folder
    from .io.disparity import write_disparity
    from .io.pairfile import write_pairfile
    from .io.raster import write_geotiff
    from .products.visualize import write_png

    outdir = Path(outdir)
    parent = check_output_folder(outdir)
    if outdir.is_dir() and not overwrite:
        present = [f for f in FILES if (outdir / f).exists()]
        if present:
            raise RiverbedError(f"{present[0]} exists; pass --overwrite to replace the block", outdir)
    command = command or f"riverbed sample OUTDIR --size {block.spec.name} --seed {block.seed}"
    tmp = Path(tempfile.mkdtemp(prefix=f".{outdir.name}.", suffix=".tmp", dir=parent))
    try:
        write_png(tmp / "left.png", block.left)
        write_png(tmp / "right.png", block.right)
        write_pairfile(tmp / "pair.yaml", block.pair(tmp),
                       comment=f"Rectified pair of the synthetic aerial block ({command}).")
        write_laz(tmp / "lidar.laz", block.lidar, block.scene.origin)
        write_disparity(tmp / "gt_disparity.tif", block.gt_disparity,
                        tags={"riverbed_ground_truth": "disparity d = x_left - x_right (px), NaN unknown",
                              "riverbed_sample": f"{block.spec.name} seed {block.seed}"})
        write_geotiff(tmp / "gt_dsm.tif", block.dsm, block.dsm_grid.transform, crs=CRS, nodata=NODATA,
                      tags={"riverbed_ground_truth": "surface height at cell centres",
                            "riverbed_sample": f"{block.spec.name} seed {block.seed}"})
        text = json.dumps(scene_description(block), indent=1) + "\n"
        (tmp / "scene.json").write_text(text, encoding="utf-8")
        (tmp / "MANIFEST.md").write_text(_manifest(block, command), encoding="utf-8")
        write_raw_frames(block, tmp / "raw", command)
        outdir.mkdir(exist_ok=True)
        if (outdir / "raw").is_dir():  # a folder is not replaced by os.replace: move the old one out first
            os.replace(outdir / "raw", tmp / "raw.old")
        sizes = {}
        for name in FILES:
            os.replace(tmp / name, outdir / name)
            sizes[name] = (outdir / name).stat().st_size
        sizes["raw"] = sum(p.stat().st_size for p in (outdir / "raw").iterdir())
        return sizes
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def raw_orientation(block, k):
    """The orientation file contents (``docs/rectify.md``) of raw frame ``k``: the camera that rendered it."""
    from .geometry.rectify import orientation_dict

    cam = block.frames[k][0]
    origin = block.scene.origin
    return orientation_dict(cam.K, cam.R, cam.C + origin, cam.width, cam.height, dist=np.zeros(5), crs=CRS,
                            origin=origin, pixel_size_mm=RAW_PIXEL_SIZE_MM)


def write_raw_frames(block, folder, command=None):
    """Render the raw frames :data:`RAW_FRAMES` (:func:`render_frame`, stored grey to keep the block small)
    into ``folder`` (created) as ``frameK.png``, with their orientation files ``frameK.yaml``."""
    from .geometry.rectify import write_orientation
    from .products.visualize import write_png

    folder = Path(folder)
    folder.mkdir()
    for k in RAW_FRAMES:
        img, _, _ = render_frame(block, k)
        write_png(folder / f"frame{k}.png", cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
        att = ", ".join(f"{a:g}" for a in block.frames[k][1])
        comment = (f"Raw frame {k} of the synthetic aerial block ({command or 'riverbed sample'}): nadir, "
                   f"roll/pitch/yaw ({att}) deg.\nOrientation file of riverbed rectify (docs/rectify.md); "
                   "omega/phi/kappa: M = R3(kappa) R2(phi) R1(omega).")
        write_orientation(folder / f"frame{k}.yaml", raw_orientation(block, k), comment=comment)


def write_laz(path, lidar, origin, date=datetime.date(2022, 6, 14)):
    """Write simulated LiDAR as LAZ (LAS 1.4, point format 7: GPS time and RGB), EPSG:32632 as a WKT VLR.

    Offsets are the minimum rounded down to whole kilometres (heights: to 100 m), scales 1 mm; the header date
    is fixed so the file is reproducible.
    """
    import laspy
    import pyproj

    xyz = lidar["xyz"] + np.asarray(origin)
    header = laspy.LasHeader(point_format=7, version="1.4")
    lo = xyz.min(axis=0)
    header.offsets = np.array([math.floor(lo[0] / 1000) * 1000, math.floor(lo[1] / 1000) * 1000,
                               math.floor(lo[2] / 100) * 100], np.float64)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.add_crs(pyproj.CRS.from_user_input(CRS))
    header.system_identifier = "riverbed synthetic ALS"
    header.generating_software = "riverbed sample"
    header.creation_date = date
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.intensity = lidar["intensity"]
    las.return_number = lidar["return_number"]
    las.number_of_returns = lidar["number_of_returns"]
    las.scan_direction_flag = lidar["scan_direction"].astype(np.uint8)
    las.edge_of_flight_line = lidar["edge_of_flight_line"].astype(np.uint8)
    las.classification = lidar["classification"]
    las.scan_angle = np.round(lidar["scan_angle_deg"] / 0.006).astype(np.int16)
    las.point_source_id = lidar["point_source_id"]
    las.gps_time = lidar["gps_time"]
    las.red, las.green, las.blue = lidar["rgb"][:, 0], lidar["rgb"][:, 1], lidar["rgb"][:, 2]
    las.write(str(path), do_compress=True, laz_backend=laspy.LazBackend.Lazrs)


def generate_block(outdir, size="small", seed=0, overwrite=False, command=None, progress=None):
    """Generate a block and write it into ``outdir``; return a summary (files, sizes, timings, key numbers).

    ``command`` is the command line quoted in MANIFEST.md (default ``riverbed sample OUTDIR --size ... --seed
    ...``); ``progress`` is called with each stage name of :data:`STAGES` once it is done.
    """
    t0 = time.perf_counter()
    # Refuse an existing block before spending the time to make a new one.
    outdir = Path(outdir)
    if outdir.is_dir() and not overwrite and any((outdir / f).exists() for f in FILES):
        present = next(f for f in FILES if (outdir / f).exists())
        raise RiverbedError(f"{present} exists; pass --overwrite to replace the block", outdir)
    block = make_block(size, seed, progress)
    t1 = time.perf_counter()
    sizes = write_block(block, outdir, overwrite, command)
    block.seconds["write"] = time.perf_counter() - t1
    if progress:
        progress("write")
    d = block.gt_disparity[np.isfinite(block.gt_disparity)]
    return {
        "outdir": str(outdir), "size": size, "seed": seed, "files": sizes, "bytes": sum(sizes.values()),
        "image": list(block.spec.rect_size), "gsd_m": block.spec.gsd, "crs": CRS,
        "origin": [float(v) for v in block.scene.origin],
        "disparity_range_px": [round(float(d.min()), 3), round(float(d.max()), 3)],
        "lidar_points": len(block.lidar["xyz"]),
        "seconds": {k: round(v, 3) for k, v in {**block.seconds, "total": time.perf_counter() - t0}.items()},
    }


if __name__ == "__main__":  # python -m riverbed_cli.sample OUTDIR [options]
    from riverbed_cli.cli.main import cli

    cli.main(args=["sample", *sys.argv[1:]], prog_name="riverbed")
